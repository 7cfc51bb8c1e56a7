%% @doc Internal. Parser of the activity and policy rules file
%% (docs/rules.md): simple activities (one sensor reading), complex
%% activities (several activities within a time window, Fig. 10 of the
%% paper) and action policies (what to do on an activity or at a time of
%% day). Line-based; every name stays a binary, keywords map to atoms only
%% through the fixed tables below, and any mistake gives an error naming
%% its line.
-module(reference_agents_rules).

-export([parse/1, parse_file/1, format_error/1, format_error/2]).
-export([simple/1, complex/1, policy_rules/2, policies/1, format_action/1, format_rule/1]).

-export_type([rules/0, simple/0, complex/0, rule/0, action/0, condition/0, error/0]).

-type simple() :: #{name := binary(), service := binary(),
                    params := [{binary(), binary()}], line := pos_integer()}.
-type complex() :: #{name := binary(), parts := [binary()], unless := [binary()],
                     window := pos_integer(), line := pos_integer()}.
-type condition() :: dark | {between, Minute :: 0..1439, Minute :: 0..1439}.
-type action() :: {light, Room :: binary(), on | off}
                | {photos, pos_integer()}
                | {email, Subject :: binary(), with_photos | no_photos}
                | {sms, binary()}
                | alarm
                | {say, binary()}.
-type rule() :: #{policy := binary(),
                  trigger := {activity, binary(), Room :: binary() | any}
                           | {at, Minute :: 0..1439},
                  conditions := [condition()],
                  actions := [action(), ...],
                  line := pos_integer()}.
-opaque rules() :: #{simple := [simple()], complex := [complex()], rules := [rule()]}.
-type error() :: #{line := non_neg_integer(), message := binary()}.

-define(MAX_SIZE, 1048576).
-define(MAX_NAME, 64).
-define(MAX_TEXT, 500).
-define(MAX_PHOTOS, 20).

%% ---------------------------------------------------------------------------
%% API
%% ---------------------------------------------------------------------------

%% @doc Parses the text of a rules file.
-spec parse(binary()) -> {ok, rules()} | {error, error()}.
parse(Text) when is_binary(Text), byte_size(Text) > ?MAX_SIZE ->
    {error, #{line => 0, message => <<"the rules file is larger than 1 MiB">>}};
parse(Text) when is_binary(Text) ->
    Lines = binary:split(Text, [<<"\r\n">>, <<"\n">>], [global]),
    try
        Statements = statements(Lines, 1, []),
        {ok, check(Statements)}
    catch
        throw:{rules_error, Line, Message} ->
            {error, #{line => Line, message => iolist_to_binary(Message)}}
    end.

%% @doc Reads and parses a rules file.
-spec parse_file(file:filename_all()) ->
          {ok, rules()} | {error, error() | {file, file:posix() | badarg | terminated}}.
parse_file(Path) ->
    case file:read_file(Path) of
        {ok, Text} -> parse(Text);
        {error, Why} -> {error, {file, Why}}
    end.

%% @doc One line for a person: `line 12: unknown action explode ...'.
-spec format_error(error()) -> binary().
format_error(#{line := 0, message := M}) -> M;
format_error(#{line := L, message := M}) ->
    iolist_to_binary(["line ", integer_to_binary(L), ": ", M]).

%% @doc The same, prefixed with the file name: `home.rules:12: ...'.
-spec format_error(file:filename_all(), error() | {file, term()}) -> binary().
format_error(File, {file, Why}) ->
    iolist_to_binary([to_chars(File), ": cannot read: ", file:format_error(Why)]);
format_error(File, #{line := 0, message := M}) ->
    iolist_to_binary([to_chars(File), ": ", M]);
format_error(File, #{line := L, message := M}) ->
    iolist_to_binary([to_chars(File), ":", integer_to_binary(L), ": ", M]).

to_chars(File) when is_binary(File) -> File;
to_chars(File) -> unicode:characters_to_binary(File).

%% @doc The simple activities, in file order.
-spec simple(rules()) -> [simple()].
simple(#{simple := S}) -> S.

%% @doc The complex activities, in file order (each after its parts).
-spec complex(rules()) -> [complex()].
complex(#{complex := C}) -> C.

%% @doc The rules of one policy, in file order.
-spec policy_rules(binary(), rules()) -> [rule()].
policy_rules(Policy, #{rules := Rules}) ->
    [R || #{policy := P} = R <- Rules, P =:= Policy].

%% @doc The names of the policies the file defines, in order of appearance.
-spec policies(rules()) -> [binary()].
policies(#{rules := Rules}) ->
    lists:foldl(fun(#{policy := P}, Acc) ->
                        case lists:member(P, Acc) of
                            true -> Acc;
                            false -> Acc ++ [P]
                        end
                end, [], Rules).

%% ---------------------------------------------------------------------------
%% Lines to statements
%% ---------------------------------------------------------------------------

statements([], _N, Acc) ->
    lists:reverse(Acc);
statements([Line | Rest], N, Acc) ->
    case unicode:characters_to_list(Line) of
        Chars when is_list(Chars) ->
            case tokens(Chars, N, 1, []) of
                [] -> statements(Rest, N + 1, Acc);
                Tokens -> statements(Rest, N + 1, [statement(Tokens, N) | Acc])
            end;
        _ ->
            fail(N, "the line is not valid UTF-8")
    end.

%% Tokens: {word, Col, Text}, {string, Col, Text}, {comma, Col}, {equals, Col}.
tokens([], _N, _Col, Acc) ->
    lists:reverse(Acc);
tokens([$# | _], _N, _Col, Acc) ->
    lists:reverse(Acc);
tokens([C | Rest], N, Col, Acc) when C =:= $\s; C =:= $\t; C =:= $\r ->
    tokens(Rest, N, Col + 1, Acc);
tokens([$, | Rest], N, Col, Acc) ->
    tokens(Rest, N, Col + 1, [{comma, Col} | Acc]);
tokens([$= | Rest], N, Col, Acc) ->
    tokens(Rest, N, Col + 1, [{equals, Col} | Acc]);
tokens([$" | Rest], N, Col, Acc) ->
    {Text, Rest1, Used} = quoted(Rest, N, Col, [], 1),
    tokens(Rest1, N, Col + Used, [{string, Col, Text} | Acc]);
tokens(Chars, N, Col, Acc) ->
    {Word, Rest} = lists:splitwith(fun(C) -> not lists:member(C, " \t\r,=\"#") end, Chars),
    tokens(Rest, N, Col + length(Word), [{word, Col, unicode:characters_to_binary(Word)} | Acc]).

quoted([], N, Col, _Acc, _Used) ->
    fail(N, ["the string starting at column ", integer_to_list(Col), " has no closing quote"]);
quoted([$" | Rest], _N, _Col, Acc, Used) ->
    {unicode:characters_to_binary(lists:reverse(Acc)), Rest, Used + 1};
quoted([$\\, C | Rest], N, Col, Acc, Used) when C =:= $"; C =:= $\\ ->
    quoted(Rest, N, Col, [C | Acc], Used + 2);
quoted([C | Rest], N, Col, Acc, Used) ->
    quoted(Rest, N, Col, [C | Acc], Used + 1).

statement([{word, _, First} | Rest] = Tokens, N) ->
    case lower(First) of
        <<"simple">> -> simple_statement(Rest, N);
        <<"complex">> -> complex_statement(Rest, N);
        <<"policy">> -> policy_statement(Rest, N);
        _ -> fail(N, ["a line starts with simple, complex or policy, not ", show(hd(Tokens))])
    end;
statement([Token | _], N) ->
    fail(N, ["a line starts with simple, complex or policy, not ", show(Token)]).

%% simple NAME when SERVICE {PARAM=VALUE}
simple_statement(Tokens, N) ->
    {Name, T1} = name(Tokens, N, "an activity name after simple"),
    T2 = keyword(<<"when">>, T1, N),
    {Service, T3} = service(T2, N),
    Params = params(T3, N, []),
    {simple, #{name => Name, service => Service, params => Params, line => N}}.

params([], _N, Acc) ->
    lists:reverse(Acc);
params([{word, _, P}, {equals, _}, V | Rest], N, Acc) ->
    Value = case V of
                {word, _, W} -> W;
                {string, _, S} -> S;
                _ -> fail(N, ["a value after ", P, "=, not ", show(V)])
            end,
    ok = valid_name(P, N, "a parameter name"),
    case lists:keymember(P, 1, Acc) of
        true -> fail(N, ["the parameter ", P, " is given twice"]);
        false -> params(Rest, N, [{P, Value} | Acc])
    end;
params([Token | _], N, _Acc) ->
    fail(N, ["expected a parameter Name=Value, not ", show(Token)]).

%% complex NAME when PART {and PART} within DURATION [unless PART {and PART}]
complex_statement(Tokens, N) ->
    {Name, T1} = name(Tokens, N, "an activity name after complex"),
    T2 = keyword(<<"when">>, T1, N),
    {Parts, T3} = names_joined(T2, N),
    case Parts of
        [_] -> fail(N, "a complex activity needs at least two parts joined by and");
        _ -> ok
    end,
    T4 = keyword(<<"within">>, T3, N),
    {Window, T5} = duration(T4, N),
    Unless = case T5 of
                 [] -> [];
                 [{word, _, W} | T6] ->
                     case lower(W) of
                         <<"unless">> ->
                             case names_joined(T6, N) of
                                 {Us, []} -> Us;
                                 {_, [Extra | _]} -> fail(N, ["unexpected ", show(Extra)])
                             end;
                         _ -> fail(N, ["expected unless or the end of the line, not ", W])
                     end;
                 [Extra | _] ->
                     fail(N, ["expected unless or the end of the line, not ", show(Extra)])
             end,
    {complex, #{name => Name, parts => Parts, unless => Unless, window => Window, line => N}}.

names_joined(Tokens, N) ->
    {First, Rest} = name(Tokens, N, "an activity name"),
    names_more(Rest, N, [First]).

names_more([{word, _, And} | Rest] = Tokens, N, Acc) ->
    case lower(And) of
        <<"and">> ->
            {Next, Rest1} = name(Rest, N, "an activity name after and"),
            names_more(Rest1, N, [Next | Acc]);
        _ -> {lists:reverse(Acc), Tokens}
    end;
names_more(Tokens, _N, Acc) ->
    {lists:reverse(Acc), Tokens}.

%% policy POLICY on ACTIVITY [in ROOM] [if CONDS] do ACTIONS
%% policy POLICY at HH:MM [if CONDS] do ACTIONS
policy_statement(Tokens, N) ->
    {Policy, T1} = name(Tokens, N, "a policy name after policy"),
    {Trigger, T2} =
        case T1 of
            [{word, _, K} | Rest] ->
                case lower(K) of
                    <<"on">> ->
                        {Activity, R1} = name(Rest, N, "an activity name after on"),
                        case R1 of
                            [{word, _, In} | R2] ->
                                case lower(In) of
                                    <<"in">> ->
                                        {Room, R3} = name(R2, N, "a room after in"),
                                        {{activity, Activity, Room}, R3};
                                    _ -> {{activity, Activity, any}, R1}
                                end;
                            _ -> {{activity, Activity, any}, R1}
                        end;
                    <<"at">> ->
                        {Minute, R1} = time_of_day(Rest, N),
                        {{at, Minute}, R1};
                    _ -> fail(N, ["expected on ACTIVITY or at HH:MM after the policy name, not ", K])
                end;
            _ -> fail(N, "expected on ACTIVITY or at HH:MM after the policy name")
        end,
    {Conditions, T3} = conditions(T2, N),
    T4 = keyword(<<"do">>, T3, N),
    Actions = actions(T4, N, []),
    {rule, #{policy => Policy, trigger => Trigger, conditions => Conditions,
             actions => Actions, line => N}}.

conditions([{word, _, If} | Rest] = Tokens, N) ->
    case lower(If) of
        <<"if">> -> condition(Rest, N, []);
        _ -> {[], Tokens}
    end;
conditions(Tokens, _N) ->
    {[], Tokens}.

condition([{word, _, W} | Rest], N, Acc) ->
    {Cond, Rest1} =
        case lower(W) of
            <<"dark">> -> {dark, Rest};
            <<"between">> ->
                {From, R1} = time_of_day(Rest, N),
                R2 = keyword(<<"and">>, R1, N),
                {To, R3} = time_of_day(R2, N),
                {{between, From, To}, R3};
            _ -> fail(N, ["unknown condition ", W, " (expected dark or between HH:MM and HH:MM)"])
        end,
    case Rest1 of
        [{word, _, And} | Rest2] ->
            case lower(And) of
                <<"and">> -> condition(Rest2, N, [Cond | Acc]);
                _ -> {lists:reverse([Cond | Acc]), Rest1}
            end;
        _ -> {lists:reverse([Cond | Acc]), Rest1}
    end;
condition(_Tokens, N, _Acc) ->
    fail(N, "expected a condition after if (dark, or between HH:MM and HH:MM)").

actions(Tokens, N, Acc) ->
    {Action, Rest} = action(Tokens, N),
    case Rest of
        [] -> lists:reverse([Action | Acc]);
        [{comma, _} | Rest1] -> actions(Rest1, N, [Action | Acc]);
        [Token | _] -> fail(N, ["expected a comma or the end of the line, not ", show(Token)])
    end.

action([{word, _, W} | Rest], N) ->
    case lower(W) of
        <<"light">> ->
            {Room, R1} = name(Rest, N, "a room after light"),
            case R1 of
                [{word, _, OnOff} | R2] ->
                    case lower(OnOff) of
                        <<"on">> -> {{light, Room, on}, R2};
                        <<"off">> -> {{light, Room, off}, R2};
                        _ -> fail(N, ["expected on or off after light ", Room, ", not ", OnOff])
                    end;
                _ -> fail(N, ["expected on or off after light ", Room])
            end;
        <<"photos">> ->
            case Rest of
                [{word, _, Count} | R1] ->
                    case to_integer(Count) of
                        C when is_integer(C), C >= 1, C =< ?MAX_PHOTOS -> {{photos, C}, R1};
                        _ -> fail(N, ["photos takes a count from 1 to 20, not ", Count])
                    end;
                _ -> fail(N, "photos takes a count from 1 to 20")
            end;
        <<"email">> ->
            {Subject, R1} = text(Rest, N, "email"),
            case R1 of
                [{word, _, With}, {word, _, Photos} | R2] ->
                    case {lower(With), lower(Photos)} of
                        {<<"with">>, <<"photos">>} -> {{email, Subject, with_photos}, R2};
                        _ -> fail(N, ["expected with photos after the subject, not ", With])
                    end;
                _ -> {{email, Subject, no_photos}, R1}
            end;
        <<"sms">> ->
            {Message, R1} = text(Rest, N, "sms"),
            {{sms, Message}, R1};
        <<"say">> ->
            {Message, R1} = text(Rest, N, "say"),
            {{say, Message}, R1};
        <<"alarm">> ->
            {alarm, Rest};
        _ ->
            fail(N, ["unknown action ", W,
                     " (expected light, photos, email, sms, say or alarm)"])
    end;
action([Token | _], N) ->
    fail(N, ["expected an action, not ", show(Token)]);
action([], N) ->
    fail(N, "expected an action after do").

text([{string, _, S} | Rest], N, _What) when byte_size(S) =< ?MAX_TEXT, S =/= <<>> ->
    case valid_text(S) of
        true -> {S, Rest};
        false -> fail(N, "a text may not contain control characters")
    end;
text([{string, _, _} | _], N, What) ->
    fail(N, [What, " takes a text of 1 to 500 bytes"]);
text(_, N, What) ->
    fail(N, [What, " takes a text in double quotes"]).

valid_text(S) ->
    lists:all(fun(C) -> C >= 32 orelse C =:= $\t end, unicode:characters_to_list(S)).

%% ---------------------------------------------------------------------------
%% Small pieces
%% ---------------------------------------------------------------------------

name([{word, _, W} | Rest], N, What) ->
    ok = valid_name(W, N, What),
    {W, Rest};
name([Token | _], N, What) ->
    fail(N, ["expected ", What, ", not ", show(Token)]);
name([], N, What) ->
    fail(N, ["expected ", What, " before the end of the line"]).

valid_name(W, N, What) ->
    case re:run(W, <<"^[A-Za-z][A-Za-z0-9_-]*$">>, [unicode]) of
        {match, _} when byte_size(W) =< ?MAX_NAME -> ok;
        _ -> fail(N, [What, " is a letter followed by letters, digits, _ or - "
                      "(at most 64), not ", W])
    end.

service([{word, _, W} | Rest], N) ->
    ok = valid_name(W, N, "a sensor service"),
    {W, Rest};
service([{string, _, S} | Rest], N) when S =/= <<>>, byte_size(S) =< ?MAX_NAME ->
    case valid_text(S) of
        true -> {S, Rest};
        false -> fail(N, "a sensor service may not contain control characters")
    end;
service(_, N) ->
    fail(N, "expected the sensor service after when (for example MotionDetected)").

keyword(K, [{word, _, W} | Rest], N) ->
    case lower(W) of
        K -> Rest;
        _ -> fail(N, ["expected ", K, ", not ", W])
    end;
keyword(K, [Token | _], N) ->
    fail(N, ["expected ", K, ", not ", show(Token)]);
keyword(K, [], N) ->
    fail(N, ["expected ", K, " before the end of the line"]).

%% A number and a unit, written together (90s) or apart (90 s).
duration([{word, _, W} | Rest], N) ->
    case re:run(W, <<"^([0-9]{1,9})([a-z]*)$">>, [{capture, all_but_first, binary}]) of
        {match, [Digits, <<>>]} ->
            case Rest of
                [{word, _, Unit} | Rest1] -> {window(Digits, lower(Unit), N), Rest1};
                _ -> fail(N, ["the duration ", Digits, " needs a unit (s, min or h)"])
            end;
        {match, [Digits, Unit]} ->
            {window(Digits, Unit, N), Rest};
        nomatch ->
            fail(N, ["expected a duration such as 90 s or 2 min after within, not ", W])
    end;
duration(_, N) ->
    fail(N, "expected a duration such as 90 s or 2 min after within").

window(Digits, Unit, N) ->
    Scale = case Unit of
                U when U =:= <<"s">>; U =:= <<"sec">>; U =:= <<"second">>;
                       U =:= <<"seconds">> -> 1000;
                U when U =:= <<"m">>; U =:= <<"min">>; U =:= <<"minute">>;
                       U =:= <<"minutes">> -> 60000;
                U when U =:= <<"h">>; U =:= <<"hour">>; U =:= <<"hours">> -> 3600000;
                _ -> fail(N, ["unknown time unit ", Unit, " (expected s, min or h)"])
            end,
    case binary_to_integer(Digits) * Scale of
        0 -> fail(N, "a time window must be longer than 0");
        Ms when Ms > 7 * 86400000 -> fail(N, "a time window is at most 7 days");
        Ms -> Ms
    end.

time_of_day([{word, _, W} | Rest], N) ->
    case re:run(W, <<"^([0-9]{1,2}):([0-9]{2})$">>, [{capture, all_but_first, binary}]) of
        {match, [H, M]} ->
            case {binary_to_integer(H), binary_to_integer(M)} of
                {Hi, Mi} when Hi < 24, Mi < 60 -> {Hi * 60 + Mi, Rest};
                _ -> fail(N, ["no such time of day: ", W])
            end;
        nomatch -> fail(N, ["expected a time of day HH:MM, not ", W])
    end;
time_of_day(_, N) ->
    fail(N, "expected a time of day HH:MM").

to_integer(B) ->
    case re:run(B, <<"^[0-9]{1,3}$">>) of
        {match, _} -> binary_to_integer(B);
        nomatch -> undefined
    end.

lower(W) -> string:lowercase(W).

show({word, _, W}) -> W;
show({string, _, S}) -> [$", S, $"];
show({comma, _}) -> "a comma";
show({equals, _}) -> "=".

-spec fail(non_neg_integer(), iodata()) -> no_return().
fail(Line, Message) ->
    throw({rules_error, Line, Message}).

%% ---------------------------------------------------------------------------
%% Whole-file checks: names defined once, parts before use, triggers known
%% ---------------------------------------------------------------------------

check(Statements) ->
    {Simple, Complex, Rules, _Defined} =
        lists:foldl(fun check_one/2, {[], [], [], #{}}, Statements),
    Known = maps:from_list([{Name, true} || #{name := Name} <- Simple ++ Complex]),
    lists:foreach(
      fun(#{trigger := {activity, A, _}, line := L}) ->
              case maps:is_key(A, Known) of
                  true -> ok;
                  false -> fail(L, ["unknown activity ", A,
                                    ": define it with a simple or complex line"])
              end;
         (_) -> ok
      end, Rules),
    #{simple => lists:reverse(Simple), complex => lists:reverse(Complex),
      rules => lists:reverse(Rules)}.

check_one({simple, #{name := Name, line := L} = S}, {Ss, Cs, Rs, Defined}) ->
    %% Several simple lines with one name are alternatives (any of them).
    Defined1 = case Defined of
                   #{Name := {simple, _}} -> Defined;
                   _ -> define(Name, simple, L, Defined)
               end,
    {[S | Ss], Cs, Rs, Defined1};
check_one({complex, #{name := Name, parts := Parts, unless := Unless, line := L} = C},
          {Ss, Cs, Rs, Defined}) ->
    lists:foreach(
      fun(P) when P =:= Name ->
              fail(L, ["the complex activity ", Name, " cannot be a part of itself"]);
         (P) ->
              case maps:is_key(P, Defined) of
                  true -> ok;
                  false -> fail(L, ["unknown activity ", P,
                                    ": define it on a line before this one"])
              end
      end, Parts ++ Unless),
    case length(Parts) =:= length(lists:usort(Parts)) of
        true -> ok;
        false -> fail(L, "a complex activity names each part once")
    end,
    {Ss, [C | Cs], Rs, define(Name, complex, L, Defined)};
check_one({rule, R}, {Ss, Cs, Rs, Defined}) ->
    {Ss, Cs, [R | Rs], Defined}.

define(Name, Kind, L, Defined) ->
    case Defined of
        #{Name := {_, First}} ->
            fail(L, ["the activity ", Name, " is already defined on line ",
                     integer_to_binary(First),
                     case Kind of
                         simple -> " (only simple lines may share a name)";
                         complex -> ""
                     end]);
        _ -> Defined#{Name => {Kind, L}}
    end.

%% ---------------------------------------------------------------------------
%% Rules and actions as text, for the narration
%% ---------------------------------------------------------------------------

%% @doc An action as it is written in the file.
-spec format_action(action()) -> iodata().
format_action({light, Room, OnOff}) -> ["light ", Room, " ", atom_to_list(OnOff)];
format_action({photos, N}) -> ["photos ", integer_to_list(N)];
format_action({email, Subject, with_photos}) -> ["email ", quote(Subject), " with photos"];
format_action({email, Subject, no_photos}) -> ["email ", quote(Subject)];
format_action({sms, Text}) -> ["sms ", quote(Text)];
format_action({say, Text}) -> ["say ", quote(Text)];
format_action(alarm) -> "alarm".

%% @doc A policy rule as text: `holiday at 18:00 if dark do light living on'.
-spec format_rule(rule()) -> iodata().
format_rule(#{policy := P, trigger := Trigger, conditions := Cs, actions := As}) ->
    [P, " ",
     case Trigger of
         {activity, A, any} -> ["on ", A];
         {activity, A, Room} -> ["on ", A, " in ", Room];
         {at, M} -> ["at ", reference_agents_policy:format_minute(M)]
     end,
     case Cs of
         [] -> [];
         _ -> [" if ", lists:join(" and ", [format_condition(C) || C <- Cs])]
     end,
     " do ", lists:join(", ", [format_action(A) || A <- As])].

format_condition(dark) -> "dark";
format_condition({between, A, B}) ->
    ["between ", reference_agents_policy:format_minute(A), " and ",
     reference_agents_policy:format_minute(B)].

quote(Text) ->
    [$", string:replace(string:replace(Text, "\\", "\\\\", all), "\"", "\\\"", all), $"].
