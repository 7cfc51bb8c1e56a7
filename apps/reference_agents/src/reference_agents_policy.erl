%% @doc Internal. Action policies, pure: which actions of the rules file a
%% policy (holiday, away, sleep, ...) takes for a recognised activity, or
%% when the clock passes one of its times of day, given the conditions
%% (dark, between two times). Darkness comes from the time sensor: after
%% sunset and before sunrise.
-module(reference_agents_policy).

-export([on_activity/4, on_time/5, dark/3, minute/1, format_minute/1, crossed/2]).

-export_type([context/0]).

%% What the VA knows of the physical time: the minute of the day and
%% whether it is dark.
-type context() :: #{minute := 0..1439, dark := boolean()}.

%% @doc The rules of `Policy' triggered by an activity instance whose
%% conditions hold, with their actions, in file order.
-spec on_activity(binary(), reference_agents_activity:instance(), context(),
                  reference_agents_rules:rules()) -> [reference_agents_rules:rule()].
on_activity(Policy, #{activity := A, room := Room}, Ctx, Rules) ->
    [R || #{trigger := {activity, Name, Where}, conditions := Cs} = R
              <- reference_agents_rules:policy_rules(Policy, Rules),
          Name =:= A, room_matches(Where, Room), holds(Cs, Ctx)].

%% @doc The rules of `Policy' whose time of day was passed when the clock
%% moved from minute `From' (excluded) to `To' (included), wrapping at
%% midnight, and whose conditions hold at `To'.
-spec on_time(binary(), 0..1439, 0..1439, context(), reference_agents_rules:rules()) ->
          [reference_agents_rules:rule()].
on_time(Policy, From, To, Ctx, Rules) ->
    [R || #{trigger := {at, M}, conditions := Cs} = R
              <- reference_agents_rules:policy_rules(Policy, Rules),
          crossed({From, To}, M), holds(Cs, Ctx)].

%% @doc Whether minute `M' is in the interval (From, To] of a clock that
%% wraps at midnight (From = To is an empty interval).
-spec crossed({0..1439, 0..1439}, 0..1439) -> boolean().
crossed({From, To}, M) when From =< To -> M > From andalso M =< To;
crossed({From, To}, M) -> M > From orelse M =< To.

%% @doc Dark: at or after sunset, or before sunrise (minutes of the day).
-spec dark(0..1439, 0..1439, 0..1439) -> boolean().
dark(Minute, Sunset, Sunrise) when Sunrise < Sunset ->
    Minute >= Sunset orelse Minute < Sunrise;
dark(Minute, Sunset, Sunrise) ->
    Minute >= Sunset andalso Minute < Sunrise.

%% @doc `<<"18:05">>' to 1085; `undefined' for anything else.
-spec minute(binary()) -> 0..1439 | undefined.
minute(HHMM) ->
    case re:run(HHMM, <<"^\\s*([0-9]{1,2}):([0-9]{2})(:[0-9]{2})?\\s*$">>,
                [{capture, [1, 2], binary}]) of
        {match, [H, M]} ->
            case {binary_to_integer(H), binary_to_integer(M)} of
                {Hi, Mi} when Hi < 24, Mi < 60 -> Hi * 60 + Mi;
                _ -> undefined
            end;
        nomatch -> undefined
    end.

%% @doc 1085 to `"18:05"'.
-spec format_minute(0..1439) -> string().
format_minute(M) ->
    io_lib:format("~2..0b:~2..0b", [M div 60, M rem 60]).

room_matches(any, _Room) -> true;
room_matches(Where, Room) when is_binary(Room) ->
    reference_agents_activity:keyword(Where) =:= reference_agents_activity:keyword(Room);
room_matches(_Where, any) -> false.

holds(Conditions, Ctx) ->
    lists:all(fun(C) -> holds1(C, Ctx) end, Conditions).

holds1(dark, #{dark := Dark}) -> Dark;
holds1({between, From, To}, #{minute := M}) when From =< To -> M >= From andalso M < To;
holds1({between, From, To}, #{minute := M}) -> M >= From orelse M < To.
