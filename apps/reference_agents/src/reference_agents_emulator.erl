%% @doc Internal. Sensor and actuator emulators (paper, section 2.2), pure:
%% built from the VA's own BIL body and the Binding report EVATAR sends, an
%% emulator table says which Avatar component each emulator drives (the
%% provider its consumer entry is bound to), which Avatar components feed
%% it readings, and what is unbound and why. A virtual actuator acts
%% through {@link request/4} instead of acting in a virtual world; a sensor
%% reading becomes a percept with {@link percept/2}.
-module(reference_agents_emulator).

-export([new/1, bind/2, emulators/1, emulator/2, kind/2, request/4, find/4,
         percept/2, bound/1, unbound/1, sources/2, entity/1, signature/1]).

-export_type([table/0, kind/0, link/0, percept/0]).

-type kind() :: actuator | behaviour | sensor | other.
%% A bound consumer entry of one emulator: the service it consumes and the
%% Avatar component providing it.
-type link() :: #{emulator := binary(), category := binary(), type := binary(),
                  parameters := [{binary(), binary()}],
                  provider := binary(), provider_entity := binary()}.
-type percept() :: #{emulator := binary(), source := binary(), service := binary(),
                     params := [{binary(), binary()}], time := integer()}.

-record(t, {entity :: binary(),
            body :: bil:description(),
            links = [] :: [link()],
            %% Avatar components that consume a service of one of our emulators:
            %% they answer or push readings to it. Emulator -> [component].
            sources = #{} :: #{binary() => [binary()]},
            unbound = [] :: [#{emulator := binary(), category := binary(),
                               type := binary(), reason := atom()}]}).
-opaque table() :: #t{}.

%% @doc A table for a VA body, nothing bound yet.
-spec new(bil:description()) -> table().
new(#{entity_id := Entity} = Body) ->
    #t{entity = Entity, body = Body}.

%% @doc Applies a Binding report as the client receives it
%% (`bil_control:binding_report()').
-spec bind(table(), bil_control:binding_report()) -> table().
bind(#t{entity = Me} = T, #{bound := Bound, unbound := Unbound}) ->
    Entries = entries(T#t.body),
    Links = [#{emulator => C, category => Cat, type => Type,
               parameters => params_of(C, Cat, Type, Entries),
               provider => PC, provider_entity => PE}
             || #{consumer := #{entity := E, component := C},
                  provider := #{entity := PE, component := PC},
                  category := Cat, type := Type} <- Bound, E =:= Me],
    Sources = lists:foldl(
                fun(#{consumer := #{entity := E, component := C},
                      provider := #{entity := PE, component := PC}}, Acc) when PE =:= Me,
                                                                          E =/= Me ->
                        maps:update_with(PC, fun(L) -> lists:usort([C | L]) end, [C], Acc);
                   (_, Acc) -> Acc
                end, #{}, Bound),
    Missing = [#{emulator => C, category => Cat, type => Type, reason => R}
               || #{consumer := #{entity := E, component := C}, category := Cat,
                    type := Type, reason := R} <- Unbound, E =:= Me],
    T#t{links = Links, sources = Sources, unbound = Missing}.

%% @doc The entity id of the VA.
-spec entity(table()) -> binary().
entity(#t{entity = E}) -> E.

%% @doc The VA's emulator ids, in body order.
-spec emulators(table()) -> [binary()].
emulators(#t{body = #{components := Cs}}) -> [Id || #{id := Id} <- Cs].

%% @doc The component of the VA's body with that id.
-spec emulator(binary(), table()) -> {ok, bil:component()} | error.
emulator(Id, #t{body = #{components := Cs}}) ->
    case [C || #{id := I} = C <- Cs, I =:= Id] of
        [C] -> {ok, C};
        [] -> error
    end.

%% @doc What an emulator stands for, from its entries: it provides SENSOR
%% data (sensor), or consumes ACTUATOR or BEHAVIOUR services.
-spec kind(binary(), table()) -> kind().
kind(Id, T) ->
    case emulator(Id, T) of
        {ok, #{services := Ss, consumes := Cs}} ->
            Provided = [key(Cat) || #{category := Cat} <- Ss],
            Consumed = [key(Cat) || #{category := Cat} <- Cs],
            case {lists:member(<<"behaviour">>, Consumed), lists:member(<<"actuator">>, Consumed),
                  lists:member(<<"sensor">>, Provided)} of
                {true, _, _} -> behaviour;
                {_, true, _} -> actuator;
                {_, _, true} -> sensor;
                _ -> other
            end;
        error -> other
    end.

%% @doc The signal an emulator sends to consume `Type' with these values,
%% addressed to the provider it is bound to; the caller adds the context.
-spec request(binary(), binary(), [{binary(), binary()}], table()) ->
          {ok, agent_bridge_client:partial_signal()} |
          {error, {not_bound, binary(), atom() | unknown}}.
request(Emulator, Type, Params, #t{links = Links, unbound = Unbound}) ->
    K = key(Type),
    case [L || #{emulator := E, type := Ty} = L <- Links, E =:= Emulator, key(Ty) =:= K] of
        [#{provider := P, category := Cat, type := Ty} | _] ->
            {ok, #{sender => Emulator, receiver => P,
                   body => #{category => Cat, type => Ty, parameters => Params}}};
        [] ->
            Why = case [R || #{emulator := E, type := Ty, reason := R} <- Unbound,
                             E =:= Emulator, key(Ty) =:= K] of
                      [R | _] -> R;
                      [] -> unknown
                  end,
            {error, {not_bound, Type, Why}}
    end.

%% @doc The emulators whose body consumes `Category'/`Type' with the given
%% parameter values (for example `[{<<"Room">>, <<"kitchen">>}]'),
%% whether bound or not.
-spec find(binary(), binary(), [{binary(), binary()}], table()) -> [binary()].
find(Category, Type, Filter, #t{body = #{components := Cs}}) ->
    [Id || #{id := Id, consumes := Consumes} <- Cs,
           lists:any(fun(#{category := C, type := Ty, parameters := Ps}) ->
                             key(C) =:= key(Category) andalso key(Ty) =:= key(Type)
                                 andalso has(Filter, Ps)
                     end, Consumes)].

%% @doc A sensor reading delivered to one of our emulators, as a percept.
-spec percept(bil:signal(), table()) -> {ok, percept()} | error.
percept(#{context := Ctx, sender := From, receiver := To, timestamp := Time,
          body := #{type := Type, parameters := Ps}}, T)
  when Ctx =:= sensor_data; Ctx =:= event ->
    case emulator(To, T) of
        {ok, _} -> {ok, #{emulator => To, source => From, service => Type, params => Ps,
                          time => Time}};
        error -> error
    end;
percept(_Signal, _T) ->
    error.

%% @doc Every bound consumer entry of the VA's emulators.
-spec bound(table()) -> [link()].
bound(#t{links = L}) -> L.

%% @doc Every consumer entry of the VA's emulators EVATAR could not bind.
-spec unbound(table()) -> [#{emulator := binary(), category := binary(), type := binary(),
                             reason := atom()}].
unbound(#t{unbound = U}) -> U.

%% @doc The Avatar components that answer or feed an emulator.
-spec sources(binary(), table()) -> [binary()].
sources(Emulator, #t{sources = S}) -> maps:get(Emulator, S, []).

%% @doc What the table binds, comparable between two reports: a new
%% signature means the VA's body changed under it and must be tested again.
-spec signature(table()) -> term().
signature(#t{links = L, sources = S}) ->
    {lists:sort([{E, key(Ty), P, PE} || #{emulator := E, type := Ty, provider := P,
                                           provider_entity := PE} <- L]),
     lists:sort(maps:to_list(S))}.

entries(#{components := Cs}) ->
    [{Id, key(Cat), key(Ty), Ps} || #{id := Id, consumes := Consumes} <- Cs,
                                    #{category := Cat, type := Ty, parameters := Ps} <- Consumes].

params_of(C, Cat, Type, Entries) ->
    case [Ps || {Id, K1, K2, Ps} <- Entries, Id =:= C, K1 =:= key(Cat), K2 =:= key(Type)] of
        [Ps | _] -> Ps;
        [] -> []
    end.

has(Filter, Ps) ->
    Have = [{key(N), key(V)} || {N, V} <- Ps],
    lists:all(fun({N, V}) -> lists:member({key(N), key(V)}, Have) end, Filter).

key(B) -> reference_agents_activity:keyword(B).
