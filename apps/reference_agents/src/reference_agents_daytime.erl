%% @doc Internal. What a VA knows of the physical time of day, pure: it
%% counts time in its own cycles, so it learns the time of day, today's
%% sunset and sunrise, and whether it is dark, from the time sensor's
%% readings (paper, section 3.2). Dark is computed from the time of day and
%% the expected sunset and sunrise once they are known, and taken from the
%% sensor's own `Dark' until then.
-module(reference_agents_daytime).

-export([new/0, update/2, context/1, known/1, minute/1, dark/1]).

-export_type([daytime/0]).

-record(dt, {minute :: 0..1439 | undefined,
             sunset :: 0..1439 | undefined,
             sunrise :: 0..1439 | undefined,
             sensor_dark :: boolean() | undefined}).
-opaque daytime() :: #dt{}.

-spec new() -> daytime().
new() -> #dt{}.

%% @doc Takes the parameters of a time sensor reading (TimeOfDay, Sunset,
%% or the ReadTime feedback). Returns the minutes the clock moved over,
%% `{From, To}' (From excluded), when the time of day advanced; the first
%% reading moves over its own minute only.
-spec update([{binary(), binary()}], daytime()) -> {daytime(), {0..1439, 0..1439} | none}.
update(Params, #dt{} = D) ->
    Get = fun(Name) ->
                  case [V || {N, V} <- Params, N =:= Name] of
                      [V | _] -> V;
                      [] -> undefined
                  end
          end,
    Minute = parse(Get(<<"TimeOfDay">>)),
    D1 = D#dt{sunset = first(parse(Get(<<"Sunset">>)), D#dt.sunset),
              sunrise = first(parse(Get(<<"Sunrise">>)), D#dt.sunrise),
              sensor_dark = case Get(<<"Dark">>) of
                                <<"yes">> -> true;
                                <<"no">> -> false;
                                _ -> D#dt.sensor_dark
                            end},
    case {Minute, D#dt.minute} of
        {undefined, _} -> {D1, none};
        {M, undefined} -> {D1#dt{minute = M}, {(M + 1439) rem 1440, M}};
        {M, M} -> {D1, none};
        {M, Prev} -> {D1#dt{minute = M}, {Prev, M}}
    end.

%% @doc The context the policies are evaluated in.
-spec context(daytime()) -> reference_agents_policy:context().
context(D) -> #{minute => minute(D), dark => dark(D)}.

%% @doc True once a time of day has been read.
-spec known(daytime()) -> boolean().
known(#dt{minute = M}) -> M =/= undefined.

-spec minute(daytime()) -> 0..1439.
minute(#dt{minute = undefined}) -> 0;
minute(#dt{minute = M}) -> M.

%% @doc Dark by time of day and sunset/sunrise; by the sensor's word when
%% those are not known; not dark when nothing is known.
-spec dark(daytime()) -> boolean().
dark(#dt{minute = M, sunset = Set, sunrise = Rise}) when is_integer(M), is_integer(Set),
                                                         is_integer(Rise) ->
    reference_agents_policy:dark(M, Set, Rise);
dark(#dt{sensor_dark = true}) -> true;
dark(_) -> false.

parse(undefined) -> undefined;
parse(V) -> reference_agents_policy:minute(V).

first(undefined, Old) -> Old;
first(New, _Old) -> New.
